"""LAS, LAZ and COPC clouds for the page: the file checked, then its points (or an evenly
spread subset of them) packed once into a compact binary the page draws without a LAS
parser, read in chunks so that memory stays bounded by the subset, not the file.

The payload, little-endian: the 8-byte magic ``ACQPTS1\\0``, uint64 points served, uint64
points in the file, float64 x y z of the origin (metres, the file's CRS), uint32 flags (bit
0: the points have colours), uint32 zero; then float32 x y z of each point as offsets from
the origin (m) and uint8 r g b of each (sRGB, LAS's 16 bits scaled to 8)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from acq.errors import InputError, first_line

__all__ = ["HEADER", "MAGIC", "SUFFIXES", "check", "payload", "shown"]

SUFFIXES = (".las", ".laz")  # a COPC file (.copc.laz) is a LAZ file
MAGIC = b"ACQPTS1\0"
HEADER = struct.Struct("<8sQQdddII")  # 56 bytes: float32 offsets after it stay aligned
HAS_COLOUR = 1
_CHUNK_POINTS = 1 << 18  # points decoded at a time (~12 MB of records)


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


def payload(path: Path, max_points: int) -> bytearray:
    """The page's binary of the LAS/LAZ file ``path`` (see the module): every point, or
    for a cloud over ``max_points`` points the ``max_points`` of index ``j * count //
    max_points`` (evenly spread along the file, the same each time); InputError naming the
    file when its points cannot be decoded or are fewer than its header says."""
    import laspy

    if max_points < 1:
        raise ValueError(f"max_points {max_points}: at least 1")

    try:
        with laspy.open(path, laz_backend=_backend()) as reader:
            count = int(reader.header.point_count)
            has_colour = {"red", "green", "blue"} <= set(reader.header.point_format.dimension_names)
            m = min(count, max_points)
            # the payload's bytes, filled in place: no copy of it is made
            data = bytearray(HEADER.size + 15 * m)
            xyz = np.frombuffer(data, np.float32, 3 * m, HEADER.size).reshape(m, 3)
            rgb16 = np.zeros((m, 3), np.uint16)
            origin: np.ndarray | None = None
            start = 0
            for chunk in reader.chunk_iterator(_CHUNK_POINTS):
                end = start + len(chunk)
                # the subset's indices j * count // m that fall in [start, end)
                lo, hi = -(-start * m // count), min(-(-end * m // count), m)
                pick = np.arange(lo, hi, dtype=np.int64) * count // m - start
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
                start = end
    except (laspy.LaspyException, ValueError, EOFError, OSError, RuntimeError) as e:
        raise InputError(f"{path}: its points cannot be read ({first_line(e)})") from None
    if start != count or origin is None:
        raise InputError(f"{path}: truncated: its header says {count} points, it holds {start}")
    if not np.isfinite(xyz).all():
        raise InputError(f"{path}: points too far apart for 32-bit floats (its scales or offsets)")
    flags = HAS_COLOUR if has_colour else 0
    HEADER.pack_into(data, 0, MAGIC, m, count, *origin.tolist(), flags, 0)
    np.frombuffer(data, np.uint8, 3 * m, HEADER.size + 12 * m)[:] = _rgb8(rgb16).ravel()
    return data


def _rgb8(rgb16: np.ndarray) -> np.ndarray:
    """LAS's 16-bit colours as 8 bits: rounded from c * 257 (as acq and the specification
    scale them); a file whose colours are all under 256 kept 8-bit values, taken as they are."""
    if rgb16.size and int(rgb16.max()) < 256:
        return rgb16.astype(np.uint8)
    return ((rgb16.astype(np.uint32) + 128) // 257).astype(np.uint8)


def _backend() -> object:
    import laspy

    return laspy.LazBackend.LazrsParallel if laspy.LazBackend.LazrsParallel.is_available() else None
