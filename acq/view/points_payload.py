"""A cloud's points as the page gets them: one packed binary for every cloud kind (PLY,
LAS, LAZ, COPC), the file's rows (or an evenly spread subset of them) read in chunks so
that memory stays bounded by the subset, not the file.

The payload, little-endian: the header (:data:`HEADER`, 80 bytes): the 8-byte magic
``ACQPTS2\\0``, uint64 points served ``m``, rows in the file, first row ``start`` and end
row ``stop`` of the range served, float64 x y z of the origin (metres, the file's CRS),
float64 time of the first point served (the file's seconds: PLY UTC, LAS GPS time),
uint32 flags (the attributes the file has: :data:`FLAGS`, and which part this is),
uint32 length of the camera names; the camera names (UTF-8, one per line, in index
order), zero-padded to 4 bytes; then the arrays: float32 x y z of each point as offsets
from the origin (m), and the attributes flagged, in :data:`COLUMNS` order: float32 time
from the first (s), uint32 scan index, float32 intensity, uint8 sRGB r g b, uint8
coloured (0/1), uint8 source camera (the index of its name, 255 none). The page's point
``j`` is the file's row ``start + j * (stop - start) // m``.

A payload may be split in two parts with the same header but for its part flag, so that
the page's first frame waits only for what it draws: :data:`POINTS_PART` holds the
positions and sRGB only, :data:`ATTRIBUTES_PART` the other attributes flagged (no
positions) of the same points."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acq.errors import InputError
from acq.view.cloud_rows import Rows, rows_of

__all__ = [
    "ATTRIBUTES_PART", "COLUMNS", "FLAGS", "HEADER", "MAGIC", "POINTS_PART", "Column", "Split",
    "payload", "positions", "rows_and_shown", "split_payload", "subset",
]  # fmt: skip

MAGIC = b"ACQPTS2\0"
# magic, served, rows, start, stop, origin x y z, first time, flags, names' bytes: 80 bytes,
# so that the arrays after it stay aligned to 4
HEADER = struct.Struct("<8sQQQQddddII")


@dataclass(frozen=True)
class Column:
    """A point attribute the payload may carry: its ``name`` in a reader's chunks, its
    flag bit, its type in the payload and its values per point."""

    name: str
    flag: int
    dtype: type[np.generic]
    width: int = 1


# in the payload's order: the 4-byte arrays first, so that each stays aligned
COLUMNS = (
    Column("time", 2, np.float32),
    Column("scan", 4, np.uint32),
    Column("intensity", 8, np.float32),
    Column("rgb", 1, np.uint8, 3),
    Column("coloured", 16, np.uint8),
    Column("camera", 32, np.uint8),
)
FLAGS = {c.name: c.flag for c in COLUMNS}
# the part flags: positions and sRGB only / the other attributes only (of the same points)
POINTS_PART, ATTRIBUTES_PART = 64, 128
_DRAWN = ("xyz", "rgb")  # what the points part holds


@dataclass(frozen=True)
class Split:
    """A payload in its two parts (:data:`POINTS_PART`, :data:`ATTRIBUTES_PART`)."""

    points: bytearray
    attributes: bytearray


def subset(start: int, stop: int, max_points: int) -> np.ndarray:
    """The rows the page gets of rows [start, stop): all of them, or ``max_points`` of
    them evenly spread, ``start + j * n // m`` for the page's point j (int64)."""
    n = stop - start
    m = min(n, max_points)
    return start + np.arange(m, dtype=np.int64) * n // m


def positions(data: bytes | bytearray) -> tuple[int, np.ndarray, np.ndarray]:
    """A payload's rows in the range it stands for, its origin (3,) float64 m and its
    points' offsets from it (m, 3) float32 (a view of ``data``)."""
    _, m, _, start, stop, ox, oy, oz, _, _, names = HEADER.unpack_from(data)
    at = HEADER.size + -(-names // 4) * 4
    offsets = np.frombuffer(data, np.float32, 3 * m, at).reshape(m, 3)
    return int(stop - start), np.array([ox, oy, oz]), offsets


def rows_and_shown(data: bytes | bytearray) -> tuple[int, int]:
    """A payload's rows in the range it stands for and the points it holds: the page's
    point j is row ``start + j * rows // shown``."""
    _, m, _, start, stop, *_ = HEADER.unpack_from(data)
    return int(stop - start), int(m)


def payload(path: Path, max_points: int, start: int = 0, stop: int | None = None) -> bytearray:
    """The page's binary (see the module) of the rows [start, stop) of the cloud file
    ``path`` (a checked layer's: :mod:`acq.view.layers`): every one, or ``max_points`` of
    them evenly spread (:func:`subset`); InputError naming the file when its points
    cannot be read, are fewer than its header says or are too far apart for float32."""
    return _payload(path, max_points, start, stop, split=False)[0]


def split_payload(path: Path, max_points: int) -> Split:
    """The page's binary of the cloud file ``path`` as :func:`payload` makes it, in its
    two parts, made in the same pass (the memory of one payload and a header)."""
    points, attributes = _payload(path, max_points, 0, None, split=True)
    return Split(points, attributes)


def _payload(
    path: Path, max_points: int, start: int, stop: int | None, split: bool
) -> list[bytearray]:
    """:func:`payload`'s checks, then the packing: one buffer, or the two parts."""
    if max_points < 1:
        raise ValueError(f"max_points {max_points}: at least 1")
    rows = rows_of(path)
    try:
        stop = rows.count if stop is None else stop
        if not 0 <= start < stop <= rows.count:
            raise ValueError(f"rows [{start}, {stop}) of a file of {rows.count}")
        return _pack(path, rows, max_points, start, stop, split)
    finally:
        rows.close()


def _pack(
    path: Path, rows: Rows, max_points: int, start: int, stop: int, split: bool
) -> list[bytearray]:
    """The payload of ``rows`` [start, stop), whole or in its two parts, filled in place
    (no copy of it is made)."""
    n = stop - start
    m = min(n, max_points)
    columns = [c for c in COLUMNS if c.name in rows.columns]
    names = "\n".join(rows.cameras).encode() if "camera" in rows.columns else b""
    # each part's arrays (name, type, values per point), in the payload's order
    arrays = [("xyz", np.float32, 3)] + [(c.name, c.dtype, c.width) for c in columns]
    parts = (
        [[a for a in arrays if a[0] in _DRAWN], [a for a in arrays if a[0] not in _DRAWN]]
        if split
        else [arrays]
    )
    head = HEADER.size + -(-len(names) // 4) * 4
    buffers: list[bytearray] = []
    out: dict[str, np.ndarray] = {}
    for part in parts:
        data = bytearray(head + sum(w * np.dtype(t).itemsize * m for _, t, w in part))
        data[HEADER.size : HEADER.size + len(names)] = names
        at = head
        for name, dtype, width in part:
            view = np.frombuffer(data, dtype, width * m, at)
            out[name] = view.reshape(m, width) if width > 1 else view
            at += width * np.dtype(dtype).itemsize * m
        buffers.append(data)
    xyz = out["xyz"]
    rgb16 = np.zeros((m, 3), np.uint16) if "rgb" in out else None
    origin = np.zeros(3)
    t0 = 0.0
    first = start
    for chunk in rows.read(start, stop):
        end = first + len(chunk["xyz"])
        # the subset's points j whose rows start + j * n // m fall in [first, end)
        lo, hi = -(-(first - start) * m // n), min(-(-(end - start) * m // n), m)
        pick = start + np.arange(lo, hi, dtype=np.int64) * n // m - first
        if len(pick):
            points = np.asarray(chunk["xyz"], np.float64)[pick]
            if lo == 0:
                origin = points[0].copy()
                if "time" in out:
                    t0 = float(chunk["time"][pick[0]])
            with np.errstate(over="ignore", invalid="ignore"):  # checked below
                xyz[lo:hi] = points - origin
                for c in columns:
                    values = np.asarray(chunk[c.name])[pick]
                    if c.name == "time":
                        out["time"][lo:hi] = values - t0
                    elif c.name == "rgb" and rgb16 is not None:
                        rgb16[lo:hi] = values
                    else:
                        out[c.name][lo:hi] = values
        first = end
    if first != stop:
        raise InputError(
            f"{path}: truncated: its header says {rows.count} points, they end at row {first}"
        )
    if not np.isfinite(xyz).all():
        why = " (its scales or offsets)" if path.suffix.lower() != ".ply" else ""
        raise InputError(f"{path}: points too far apart for 32-bit floats{why}")
    if rgb16 is not None:
        out["rgb"][:] = _rgb8(rgb16)
    flags = sum(c.flag for c in columns)
    kinds = (POINTS_PART, ATTRIBUTES_PART) if split else (0,)
    for data, kind in zip(buffers, kinds, strict=True):
        HEADER.pack_into(
            data, 0, MAGIC, m, rows.count, start, stop, *origin.tolist(), t0, flags | kind,
            len(names),
        )  # fmt: skip
    return buffers


def _rgb8(rgb16: np.ndarray) -> np.ndarray:
    """16-bit colours (LAS's) as 8 bits: rounded from c * 257 (as acq and the LAS
    specification scale them); colours all under 256 (8-bit values, a PLY's or a LAS
    file's that kept them) taken as they are."""
    if rgb16.size and int(rgb16.max()) < 256:
        return rgb16.astype(np.uint8)
    return ((rgb16.astype(np.uint32) + 128) // 257).astype(np.uint8)
