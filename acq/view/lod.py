"""Level of detail of a LAS/LAZ/COPC layer shown by a subset (:mod:`acq.view.points_payload`):
its rows split into chunks, each a range of rows [start, stop) with the box it lies in,
that the page loads at full density as the view closes in on them.

A COPC file's chunks are its octree's nodes: each node's points are one LAZ chunk, the
nodes' chunks follow one another in the file, so the nodes taken in the order of their
byte offsets hold consecutive rows (the first node rows [0, n0), the next [n0, n0 + n1),
...); their boxes are the nodes' cubes within the file's bounds (its header's), their
levels the octree's (0 the root), all read from the hierarchy alone. Any other file is
cut into runs of consecutive rows: acq writes its clouds in time order, so that a run is
a stretch of the drive. A run's box is that of its rows in the coarse subset already
decoded (the subset is spread evenly along the file: the box of the run's rows within
the subset's spacing), so the file is not decoded twice at start-up, and nothing but the
chunks' bounds is kept."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from acq.errors import InputError, first_line
from acq.view.points_payload import positions

__all__ = ["CHUNK_CAP", "RUN_POINTS", "Chunk", "chunks", "copc_chunks", "index", "runs"]

RUN_POINTS = 250_000  # rows of a run (a LAS/LAZ file's chunk): 3.75 MB for the page
CHUNK_CAP = 1_000_000  # points a chunk is served with at most (evenly spread beyond)
_MIN_SAMPLES = 64  # subset points a run's box is taken from at least


@dataclass(frozen=True)
class Chunk:
    """Rows [``start``, ``stop``) of a file, within the box ``lo``..``hi`` (x y z, m, the
    file's frame); ``level`` is its octree depth in a COPC file (0 the root), 0 for a run."""

    start: int
    stop: int
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    level: int = 0

    @property
    def count(self) -> int:
        return self.stop - self.start


def chunks(
    path: Path, count: int, coarse: bytes | bytearray, rows: int = RUN_POINTS
) -> list[Chunk]:
    """The chunks of the file ``path`` of ``count`` points: its COPC nodes when it is
    COPC, else runs of ``rows`` rows boxed by ``coarse`` (its subset's payload)."""
    found = copc_chunks(path) if path.suffix.lower() == ".laz" else None
    return found if found is not None else runs(coarse, count, rows)


def copc_chunks(path: Path) -> list[Chunk] | None:
    """The nodes of the COPC file ``path`` holding points, as chunks in file order (see
    the module); None when the file is not COPC (its first VLR is not COPC's info);
    InputError naming it when its hierarchy cannot be read or does not account for every
    point of its header."""
    import laspy
    from laspy.copc import Bounds, CopcInfoVlr, CopcReader

    try:
        with laspy.open(path) as f:
            vlrs = f.header.vlrs
            if not vlrs or not isinstance(vlrs[0], CopcInfoVlr):
                return None
            count = int(f.header.point_count)
            # a header's bounds may be those of the points before their rounding
            step = np.abs(np.asarray(f.header.scales))
            mins, maxs = np.asarray(f.header.mins) - step, np.asarray(f.header.maxs) + step
            if not (np.isfinite(mins).all() and np.isfinite(maxs).all()):
                mins, maxs = np.full(3, -np.inf), np.full(3, np.inf)  # the cubes alone
        with CopcReader.open(path) as reader:
            info = reader.copc_info
            if not (np.isfinite(info.center).all() and 0 < info.halfsize < np.inf):
                raise InputError(f"{path}: its COPC octree's centre or half size is no number")
            nodes = _entries(reader.source, reader.root_page)
    except (laspy.LaspyException, ValueError, EOFError, OSError, struct.error) as e:
        raise InputError(f"{path}: its COPC hierarchy cannot be read ({first_line(e)})") from None
    nodes = sorted(nodes, key=lambda n: n.offset)
    ends = np.cumsum([n.point_count for n in nodes], dtype=np.int64)
    if not len(nodes) or int(ends[-1]) != count:
        held = int(ends[-1]) if len(nodes) else 0
        raise InputError(
            f"{path}: its COPC hierarchy's nodes hold {held} points, its header says {count}"
        )
    root = Bounds(info.center - info.halfsize, info.center + info.halfsize)
    chunks = []
    for n, end in zip(nodes, ends, strict=True):
        cube = n.key.bounds(root)
        lo, hi = np.maximum(cube.mins, mins), np.minimum(cube.maxs, maxs)
        chunks.append(Chunk(int(end - n.point_count), int(end), _xyz(lo), _xyz(hi), n.key.level))
    return chunks


def _entries(source: Any, root: Any) -> list[Any]:
    """The entries of a COPC hierarchy that hold points (laspy's ``Entry``), its pages
    read from ``source`` from the ``root`` page on, each page once (a page that names
    itself or an earlier one does not loop)."""
    from laspy.copc import HierarchyPage

    entries, pages, seen = dict(root.entries), list(root.entries.values()), set()
    while pages:
        entry = pages.pop()
        if entry.point_count != -1 or entry.offset in seen:
            continue
        seen.add(entry.offset)
        source.seek(entry.offset)
        page = HierarchyPage.from_bytes(source.read(max(entry.byte_size, 0)))
        entries.update(page.entries)
        pages += page.entries.values()
    return [e for e in entries.values() if e.point_count > 0]


def runs(coarse: bytes | bytearray, count: int, rows: int = RUN_POINTS) -> list[Chunk]:
    """Runs of ``rows`` consecutive rows (more when the subset is too sparse to box them
    by at least 64 of its points) of a file of ``count`` points, each boxed by its rows
    in ``coarse``, the payload of the file's evenly spread subset."""
    total, origin, offsets = positions(coarse)
    m = len(offsets)
    if total != count:
        raise ValueError(f"a subset of {total} points for a file of {count}")
    rows = max(rows, -(-count * _MIN_SAMPLES // m))
    starts = np.arange(0, count, rows, dtype=np.int64)
    stops = np.minimum(starts + rows, count)
    # the subset's points of rows [start, stop): indices j with j * count // m in it
    first = -(-starts * m // count)
    boxes = np.minimum.reduceat(offsets, first), np.maximum.reduceat(offsets, first)
    return [
        Chunk(int(a), int(b), _xyz(lo + origin), _xyz(hi + origin))
        for a, b, lo, hi in zip(starts, stops, *boxes, strict=True)
    ]


def index(found: list[Chunk]) -> dict[str, Any]:
    """What ``/data/<k>/lod.json`` answers: each chunk's rows [``start``, ``stop``),
    ``count`` the points its binary holds (its rows, at most :data:`CHUNK_CAP`), ``level``
    and box (``min``, ``max``: x y z, m, the file's frame), in chunk order."""
    return {
        "chunks": [
            {
                "start": c.start,
                "stop": c.stop,
                "count": min(c.count, CHUNK_CAP),
                "level": c.level,
                "min": list(c.lo),
                "max": list(c.hi),
            }
            for c in found
        ]
    }


def _xyz(a: Any) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in a)
    return x, y, z
