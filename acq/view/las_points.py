"""LAS, LAZ and COPC clouds for the page: the file checked, then its points (or an evenly
spread subset of them) packed once into a compact binary the page draws without a LAS
parser, read in chunks so that memory stays bounded by the subset, not the file.

The payload, little-endian: the 8-byte magic ``ACQPTS1\\0``, uint64 points served, uint64
points they stand for (the file's, or a range of its rows'), float64 x y z of the origin
(metres, the file's CRS), uint32 flags (bit 0: the points have colours), uint32 zero; then
float32 x y z of each point as offsets from the origin (m) and uint8 r g b of each (sRGB,
LAS's 16 bits scaled to 8)."""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from acq.errors import InputError, first_line

__all__ = ["HEADER", "MAGIC", "SUFFIXES", "check", "payload", "shown"]

SUFFIXES = (".las", ".laz")  # a COPC file (.copc.laz) is a LAZ file
MAGIC = b"ACQPTS1\0"
HEADER = struct.Struct("<8sQQdddII")  # 56 bytes: float32 offsets after it stay aligned
HAS_COLOUR = 1
_CHUNK_POINTS = 1 << 18  # points decoded at a time (~12 MB of records)
_VARIABLE = 0xFFFFFFFF  # a LASzip VLR's chunk size for chunks of varying sizes


def check(path: Path) -> int:
    """The point count of the LAS/LAZ file ``path`` from its header, checked (a LAS
    header, finite non-zero scales and finite offsets, an uncompressed file as long as its
    header says); InputError naming it otherwise. A LAZ file's points are checked when
    :func:`payload` decodes them."""
    import laspy

    try:
        with laspy.open(path) as reader:
            header = reader.header
    except (laspy.LaspyException, ValueError, EOFError, struct.error) as e:
        raise InputError(f"{path}: not a readable LAS/LAZ file ({first_line(e)})") from None
    scales, offsets = np.asarray(header.scales), np.asarray(header.offsets)
    if not (np.isfinite(scales).all() and (scales != 0).all() and np.isfinite(offsets).all()):
        raise InputError(f"{path}: a LAS header whose scales or offsets are not finite numbers")
    count = int(header.point_count)
    if count == 0:
        raise InputError(f"{path}: a LAS file with no point")
    if not header.are_points_compressed:
        end = header.offset_to_point_data + count * header.point_format.size
        if path.stat().st_size < end:
            raise InputError(
                f"{path}: truncated: its header says {count} points, which end at byte "
                f"{end}; the file has {path.stat().st_size}"
            )
    return count


def shown(data: bytes | bytearray) -> int:
    """The points a payload holds (its header's)."""
    return int(HEADER.unpack_from(data)[1])


def payload(path: Path, max_points: int, start: int = 0, stop: int | None = None) -> bytearray:
    """The page's binary of rows [``start``, ``stop``) of the LAS/LAZ file ``path`` (see
    the module; all its rows by default): every point, or for a range over ``max_points``
    points the ``max_points`` of index ``start + j * count // max_points`` (evenly spread
    along the range, the same each time); its header's "points in the file" is the
    range's. InputError naming the file when its points cannot be decoded or are fewer
    than its header says; ValueError for a range outside its rows."""
    import laspy

    if max_points < 1:
        raise ValueError(f"max_points {max_points}: at least 1")

    try:
        with laspy.open(path, laz_backend=_backend()) as reader:
            total = int(reader.header.point_count)
            stop = total if stop is None else stop
            if not 0 <= start < stop <= total:
                raise _RowsOutside(f"{path}: rows [{start}, {stop}) of a file of {total}")
            count = stop - start
            has_colour = {"red", "green", "blue"} <= set(reader.header.point_format.dimension_names)
            m = min(count, max_points)
            # the payload's bytes, filled in place: no copy of it is made
            data = bytearray(HEADER.size + 15 * m)
            xyz = np.frombuffer(data, np.float32, 3 * m, HEADER.size).reshape(m, 3)
            rgb16 = np.zeros((m, 3), np.uint16)
            origin: np.ndarray | None = None
            done = 0  # rows of the range read
            for chunk in _records(reader, path, start, stop):
                end = done + len(chunk)
                # the subset's indices j * count // m that fall in [done, end)
                lo, hi = -(-done * m // count), min(-(-end * m // count), m)
                pick = np.arange(lo, hi, dtype=np.int64) * count // m - done
                if len(pick):
                    x, y, z = (np.asarray(chunk[a], np.float64)[pick] for a in "xyz")
                    if origin is None:
                        origin = np.array([x[0], y[0], z[0]])
                    with np.errstate(over="ignore", invalid="ignore"):  # checked below
                        xyz[lo:hi] = np.stack([x, y, z], axis=1) - origin
                    if has_colour:
                        rgb16[lo:hi] = np.stack(
                            [np.asarray(chunk[c])[pick] for c in ("red", "green", "blue")],
                            axis=1,
                        )
                done = end
    except _RowsOutside:
        raise
    except (laspy.LaspyException, ValueError, EOFError, OSError, RuntimeError) as e:
        raise InputError(f"{path}: its points cannot be read ({first_line(e)})") from None
    if done != count or origin is None:
        raise InputError(
            f"{path}: truncated: its header says {total} points, it holds {start + done}"
        )
    if not np.isfinite(xyz).all():
        raise InputError(f"{path}: points too far apart for 32-bit floats (its scales or offsets)")
    flags = HAS_COLOUR if has_colour else 0
    HEADER.pack_into(data, 0, MAGIC, m, count, *origin.tolist(), flags, 0)
    np.frombuffer(data, np.uint8, 3 * m, HEADER.size + 12 * m)[:] = _rgb8(rgb16).ravel()
    return data


def _records(reader: Any, path: Path, start: int, stop: int) -> Iterator[Any]:
    """The points of rows [``start``, ``stop``) of the file ``path`` open in laspy's
    ``reader``, a chunk of them at a time (fewer rows in all when the file is cut)."""
    import laspy
    import lazrs

    laszip = reader.header.vlrs.get("LasZipVlr")
    if start and laszip and lazrs.LazVlr(laszip[0].record_data).chunk_size() == _VARIABLE:
        # variable-size LAZ chunks (COPC's octree nodes): lazrs's seek reads wrong points
        # in them, so the chunks that hold the rows are found in the chunk table and
        # decoded alone, as laspy's COPC reader decodes a node
        record_data = laszip[0].record_data
        header = reader.header
        with open(path, "rb") as f:
            f.seek(header.offset_to_point_data)
            table = lazrs.read_chunk_table(f, lazrs.LazVlr(record_data))
            offset, first = header.offset_to_point_data + 8, 0
            for points, size in table:
                if first + points > start and first < stop:
                    f.seek(offset)
                    out = np.zeros(points * header.point_format.size, np.uint8)
                    lazrs.decompress_points_with_chunk_table(
                        f.read(size), record_data, out, [(points, size)]
                    )
                    record = laspy.PackedPointRecord.from_buffer(out, header.point_format)
                    scaled = laspy.ScaleAwarePointRecord(
                        record.array, record.point_format, header.scales, header.offsets
                    )
                    yield scaled[max(start - first, 0) : stop - first]
                offset, first = offset + size, first + points
        return
    if start:
        reader.seek(start)  # a fixed chunk size: the chunk found by the row's number
    done = start
    while done < stop:
        chunk = reader.read_points(min(_CHUNK_POINTS, stop - done))
        if len(chunk) == 0:
            return
        done += len(chunk)
        yield chunk


class _RowsOutside(ValueError):
    """A range of rows outside the file's: the caller's error, not the file's."""


def _rgb8(rgb16: np.ndarray) -> np.ndarray:
    """LAS's 16-bit colours as 8 bits: rounded from c * 257 (as acq and the specification
    scale them); a file whose colours are all under 256 kept 8-bit values, taken as they are."""
    if rgb16.size and int(rgb16.max()) < 256:
        return rgb16.astype(np.uint8)
    return ((rgb16.astype(np.uint32) + 128) // 257).astype(np.uint8)


def _backend() -> object:
    import laspy

    return laspy.LazBackend.LazrsParallel if laspy.LazBackend.LazrsParallel.is_available() else None
