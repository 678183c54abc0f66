"""LAS, LAZ and COPC clouds read for the page (:mod:`acq.view.points_payload`): the file's
header checked up front, then its rows decoded in chunks from a seek (lazrs reaches a
LAZ row through the file's chunk table; a COPC file's chunks, of varying sizes, decoded
alone), with the attributes acq writes (GPS time, as
UTC s where it is Adjusted Standard GPS time; intensity; the extra bytes ``scan_index``,
``coloured`` and ``camera`` of :mod:`acq.cloud.las`) and the cameras' names (its VLR
``acq 1``)."""

from __future__ import annotations

import logging
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from acq.errors import InputError, first_line
from acq.time.gpstime import utc_from_adjusted_standard_time
from acq.view.camera_names import camera_names

if TYPE_CHECKING:
    import laspy

__all__ = ["SUFFIXES", "LasRows", "check"]

SUFFIXES = (".las", ".laz")  # a COPC file (.copc.laz) is a LAZ file
# laspy logs the errors it raises too: acq says them once, in its own line
logging.getLogger("laspy").setLevel(logging.CRITICAL)
_CHUNK_POINTS = 1 << 18  # points decoded at a time (~12 MB of records)
_VARIABLE = 0xFFFFFFFF  # a LAZ chunk size that says the chunks vary in size (COPC's)
# the payload's columns by the LAS dimension holding them
_DIMENSIONS = {
    "time": "gps_time", "scan": "scan_index", "intensity": "intensity", "coloured": "coloured",
    "camera": "camera", "frame": "frame",
}  # fmt: skip


def check(path: Path) -> int:
    """The point count of the LAS/LAZ file ``path`` from its header, checked (a LAS
    header, finite non-zero scales and finite offsets, an uncompressed file as long as its
    header says); InputError naming it otherwise. A LAZ file's points are checked when
    they are decoded (:meth:`LasRows.read`)."""
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


class LasRows:
    """The rows of the LAS/LAZ/COPC file ``path`` (checked: :func:`check`), open until
    :meth:`close` (see :class:`acq.view.cloud_rows.Rows`)."""

    def __init__(self, path: Path) -> None:
        import laspy

        self.path = path
        try:
            self._reader = laspy.open(path, laz_backend=_backend())
        except (laspy.LaspyException, ValueError, EOFError, OSError, struct.error) as e:
            raise InputError(f"{path}: not a readable LAS/LAZ file ({first_line(e)})") from None
        header = self._reader.header
        self.count = int(header.point_count)
        names = set(header.point_format.dimension_names)
        self._rgb = {"red", "green", "blue"} <= names
        self.columns = frozenset(
            [k for k, d in _DIMENSIONS.items() if d in names] + ["rgb"] * self._rgb
        )
        self.cameras = cameras(header.vlrs)
        self.world = True  # a LAS file says nothing of it: taken as the world frame
        self._utc = header.global_encoding.gps_time_type == laspy.header.GpsTimeType.STANDARD

    def read(self, start: int, stop: int) -> Iterator[dict[str, np.ndarray]]:
        import laspy

        try:
            for chunk in self._records(start, stop):
                yield self._columns(chunk)
        except (laspy.LaspyException, ValueError, EOFError, OSError, RuntimeError) as e:
            raise InputError(f"{self.path}: its points cannot be read ({first_line(e)})") from None

    def _records(self, start: int, stop: int) -> Iterator[Any]:
        """laspy's points of rows [start, stop), a chunk of them at a time (fewer rows in
        all when the file is cut: the caller names it)."""
        import laspy
        import lazrs

        reader, header = self._reader, self._reader.header
        laszip = header.vlrs.get("LasZipVlr")
        if start and laszip and lazrs.LazVlr(laszip[0].record_data).chunk_size() == _VARIABLE:
            # variable-size LAZ chunks (COPC's octree nodes): lazrs's seek reads wrong
            # points in them, so the chunks that hold the rows are found in the chunk table
            # and decoded alone, as laspy's COPC reader decodes a node
            record_data = laszip[0].record_data
            with open(self.path, "rb") as f:
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
        at = start
        while at < stop:
            chunk = reader.read_points(min(_CHUNK_POINTS, stop - at))
            if len(chunk) == 0:
                return
            at += len(chunk)
            yield chunk

    def _columns(self, chunk: laspy.ScaleAwarePointRecord) -> dict[str, np.ndarray]:
        get = chunk.__getitem__
        out = {"xyz": np.stack([np.asarray(get(a), np.float64) for a in "xyz"], axis=1)}
        for name, dimension in _DIMENSIONS.items():
            if name in self.columns:
                out[name] = np.asarray(get(dimension))
        if "time" in out and self._utc:
            out["time"] = utc_from_adjusted_standard_time(out["time"])
        if self._rgb:
            out["rgb"] = np.stack([np.asarray(get(c)) for c in ("red", "green", "blue")], axis=1)
        return out

    def close(self) -> None:
        self._reader.close()


def cameras(vlrs: list[object]) -> list[str]:
    """The cameras' names in the VLR ``acq 1`` (lines ``<index> <name>``), by index; a
    name missing from it ``camera <index>``; none without that VLR."""
    from acq.cloud.las import CAMERAS_VLR  # here: acq.cloud's package imports numba (~100 MB)

    user, record, _ = CAMERAS_VLR
    for vlr in vlrs:
        if getattr(vlr, "user_id", None) == user and getattr(vlr, "record_id", None) == record:
            text = bytes(getattr(vlr, "record_data", b"")).decode("ascii", "replace")
            return camera_names(text.splitlines())
    return []


def _backend() -> object:
    import laspy

    return laspy.LazBackend.LazrsParallel if laspy.LazBackend.LazrsParallel.is_available() else None
