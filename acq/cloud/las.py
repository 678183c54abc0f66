"""Coloured clouds as LAS 1.4 or LAZ (laspy; LAZ compressed by lazrs), for CloudCompare,
PDAL and QGIS.

Point format 7 (x, y, z, intensity, GPS time, RGB) with Adjusted Standard GPS time (GPS
seconds minus 1e9, the global-encoding bit set), scale 1 mm and an offset at the
cloud's rounded minimum so coordinates keep millimetres, and the coordinate reference
system from ``crs`` (anything ``pyproj.CRS.from_user_input`` takes, e.g. "EPSG:25832")
as an OGC WKT 1 VLR (the WKT bit set: the form LAS 1.4 readers, PDAL and LAStools among
them, parse). Extra bytes: ``scan_index`` (uint32, the scan in the log), ``coloured``
(uint8 0/1), ``camera`` (uint8, the index of the camera that coloured the point; no_data
255) and ``frame`` (int32, the index of that camera's frame in the session; no_data -1),
with their true minimum and maximum over the points that have a value in the extra-bytes
VLR (laspy leaves them zero: written at :meth:`LasStream.close`); ``user_data`` also
holds the coloured flag for readers that ignore extra bytes. The cameras' names are a
VLR of user ID ``acq``, record ID 1 (:data:`CAMERAS_VLR`): ASCII lines ``<index> <name>``
in index order. When the log's UTC cannot be trusted (its time base says the host clock
was unsynchronised, stepped or off, or it has none), a VLR of user ID ``acq``, record
ID 2 (:data:`TIME_BASE_VLR`) says why, in ASCII: the GPS times are the host clock's.
When the cameras' calibration was checked on the drive, record ID 3
(:data:`CALIBRATION_CHECK_VLR`) holds each camera's verdict, an ASCII line each.
RGB is 16-bit (8-bit values times 257), intensity clipped to 0..65535.
Generating Software is acq's mark (:mod:`acq.provenance`); System Identifier "OTHER", the
specification's value for an operation that is neither a hardware system nor a merge,
extraction, modification or transformation of LAS files.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from acq.atomic_write import discard, release, temporary_beside
from acq.provenance import SOFTWARE
from acq.time.gpstime import gps_adjusted_standard_time

if TYPE_CHECKING:
    import laspy

__all__ = [
    "CALIBRATION_CHECK_VLR", "CAMERAS_VLR", "SYSTEM_IDENTIFIER", "TIME_BASE_VLR", "LasStream",
    "cameras_text", "extra_dims", "grow_ranges", "pack_points", "write_extra_bytes_ranges",
]  # fmt: skip

SYSTEM_IDENTIFIER = "OTHER"
# the cameras' names: the VLR's user ID, record ID and description
CAMERAS_VLR = ("acq", 1, "cameras: index name")
# why the points' GPS times (from the host clock's UTC) cannot be trusted
TIME_BASE_VLR = ("acq", 2, "time base: UTC not trusted")
# each camera's calibration checked on the drive (acq colorize --check)
CALIBRATION_CHECK_VLR = ("acq", 3, "calibration check")
# the extra-bytes dimensions in the record's order: name -> (type, no_data, description)
_EXTRA: dict[str, tuple[type[np.integer], int | None, str]] = {
    "scan_index": (np.uint32, None, "scan in the log"),
    "coloured": (np.uint8, None, "1 coloured, 0 not"),
    "camera": (np.uint8, 255, "source camera (VLR acq 1)"),
    "frame": (np.int32, -1, "frame of its camera"),
}


class LasStream:
    """A LAS 1.4 file (module docstring) written part by part to a temporary of its own
    beside ``path`` (:func:`acq.atomic_write.temporary_beside`), renamed on :meth:`close`
    (:meth:`abort` removes it); LAZ (compressed) when ``path`` ends in .laz. The offset
    is the first part's rounded minimum; the header's extent, counts and GPS time span
    grow with every part. ``cameras``: the names, in index order, of
    the cameras the points' ``camera`` indexes. ``comments`` have no place in LAS: unused.
    ``utc_doubt``: why the points' UTC cannot be trusted, as the :data:`TIME_BASE_VLR`;
    ``checks``: the calibration check's lines, as the :data:`CALIBRATION_CHECK_VLR`."""

    def __init__(
        self, path: str | os.PathLike[str], *, crs: str | None = None,
        comments: Sequence[str] = (), cameras: Sequence[str] = (), utc_doubt: str | None = None,
        checks: Sequence[str] = (),
    ) -> None:  # fmt: skip
        import laspy
        import pyproj
        from laspy.vlrs.known import WktCoordinateSystemVlr

        self.path = Path(path)
        self._compress = self.path.suffix.lower() == ".laz"
        header = laspy.LasHeader(point_format=7, version="1.4")
        header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
        header.scales = np.array([0.001, 0.001, 0.001])
        header.generating_software = SOFTWARE
        header.system_identifier = SYSTEM_IDENTIFIER
        if crs:
            wkt = pyproj.CRS.from_user_input(crs).to_wkt(pyproj.enums.WktVersion.WKT1_GDAL)
            header.vlrs.append(WktCoordinateSystemVlr(wkt))
            header.global_encoding.wkt = True
        header.add_extra_dims(extra_dims())
        if cameras:
            header.vlrs.append(laspy.VLR(*CAMERAS_VLR, cameras_text(cameras).encode()))
        if utc_doubt is not None:
            text = utc_doubt.encode("ascii", "replace")[:60000]  # a VLR holds < 64 KiB
            header.vlrs.append(laspy.VLR(*TIME_BASE_VLR, text))
        if checks:
            text = "\n".join(checks).encode("ascii", "replace")[:60000]
            header.vlrs.append(laspy.VLR(*CALIBRATION_CHECK_VLR, text))
        self._header = header
        self._tmp = temporary_beside(self.path)  # last: nothing above leaves it behind
        self._writer: laspy.LasWriter | None = None
        # each extra dimension's (min, max) over the points written; None before any
        self._ranges: dict[str, tuple[int, int]] = {}

    def write(
        self, xyz: np.ndarray, rgb: np.ndarray, utc_s: np.ndarray, intensity: np.ndarray,
        scan: np.ndarray, coloured: np.ndarray, camera: np.ndarray, frame: np.ndarray,
    ) -> None:  # fmt: skip
        """Append points: ``xyz`` (N,3) m, ``rgb`` (N,3) uint8, ``utc_s`` (N,) UTC
        seconds, ``intensity``, ``scan`` index, ``coloured`` flag, source ``camera``
        (255 none) and ``frame`` (-1 none)."""
        n = xyz.shape[0]
        if n == 0:
            return
        if self._writer is None:
            # column by column: numpy's axis-0 reduction of an (N,3) array is 9x slower
            self._header.offsets = np.floor([xyz[:, k].min() for k in range(3)])
            self._writer = self._open()
        header = self._writer.header
        record = pack_points(
            header.point_format, header.offsets, header.scales,
            xyz, rgb, utc_s, intensity, scan, coloured, camera, frame,
        )  # fmt: skip
        grow_ranges(self._ranges, record.array)
        self._writer.write_points(record)

    def _open(self) -> laspy.LasWriter:
        import laspy

        if self._compress:
            return laspy.open(
                self._tmp, mode="w", header=self._header, do_compress=True,
                laz_backend=laspy.LazBackend.LazrsParallel,
            )  # fmt: skip
        return laspy.open(self._tmp, mode="w", header=self._header, do_compress=False)

    def close(self) -> int:
        """Finish the file; its size, bytes."""
        if self._writer is None:  # no points: a valid empty file
            self._writer = self._open()
        self._writer.close()
        write_extra_bytes_ranges(self._tmp, self._ranges)
        self._tmp.replace(self.path)
        release(self._tmp)
        return self.path.stat().st_size

    def abort(self) -> None:
        """Drop the unfinished file; never raises (it runs on the way out of an error, which
        the writer's own, at closing a half-written file on a full disk, would hide)."""
        try:
            if self._writer is not None:
                self._writer.close()
        except Exception:  # the file is dropped whatever closing it says
            pass
        finally:
            discard(self._tmp)


def extra_dims() -> list[laspy.ExtraBytesParams]:
    """The extra-bytes dimensions of acq's point records (module docstring)."""
    import laspy

    return [
        laspy.ExtraBytesParams(
            name=name, type=kind, description=text,
            no_data=None if no_data is None else [no_data],
        )
        for name, (kind, no_data, text) in _EXTRA.items()
    ]  # fmt: skip


def cameras_text(cameras: Sequence[str]) -> str:
    """The cameras VLR's text: a line ``<index> <name>`` per camera, in index order;
    ValueError for a name that is not one line of printable ASCII."""
    for name in cameras:
        if not (name.isascii() and name.isprintable()):
            raise ValueError(f"a camera name is one line of printable ASCII, not {name!r}")
    return "".join(f"{k} {name}\n" for k, name in enumerate(cameras))


def pack_points(
    point_format: laspy.PointFormat, offsets: np.ndarray, scales: np.ndarray,
    xyz: np.ndarray, rgb: np.ndarray, utc_s: np.ndarray, intensity: np.ndarray,
    scan: np.ndarray, coloured: np.ndarray, camera: np.ndarray, frame: np.ndarray,
) -> laspy.PackedPointRecord:  # fmt: skip
    """The raw records of points (as :meth:`LasStream.write` takes them) in
    ``point_format`` (7 with :func:`extra_dims`), integer coordinates of ``offsets`` and
    ``scales``."""
    import laspy

    # the raw record array filled column by column (laspy's scaled setters copy and
    # check each one: three times slower on millions of points)
    record = laspy.PackedPointRecord.zeros(xyz.shape[0], point_format)
    a = record.array
    for axis, name in enumerate("XYZ"):
        a[name] = np.rint((xyz[:, axis] - offsets[axis]) / scales[axis])
    rgb16 = rgb.astype(np.uint16) * 257
    a["red"], a["green"], a["blue"] = rgb16[:, 0], rgb16[:, 1], rgb16[:, 2]
    a["intensity"] = np.clip(np.nan_to_num(intensity), 0, 65535).astype(np.uint16)
    a["gps_time"] = gps_adjusted_standard_time(utc_s)
    # one return per pulse (a 2D scanner's first echo): valid per the specification,
    # whose return numbers start at 1
    a["bit_fields"] = 0b0001_0001  # return number 1 of 1
    a["user_data"] = coloured.astype(np.uint8)
    a["scan_index"] = scan.astype(np.uint32)
    a["coloured"] = coloured.astype(np.uint8)
    a["camera"] = camera
    a["frame"] = frame
    return record


def grow_ranges(ranges: dict[str, tuple[int, int]], a: np.ndarray) -> None:
    """Widen ``ranges`` (extra dimension -> (min, max)) to the records ``a``, over the
    values that are not the dimension's no_data."""
    for name, (_, no_data, _) in _EXTRA.items():
        values = a[name] if no_data is None else a[name][a[name] != no_data]
        if values.size == 0:
            continue
        lo, hi = int(values.min()), int(values.max())
        was = ranges.get(name, (lo, hi))
        ranges[name] = (min(was[0], lo), max(was[1], hi))


# the LAS 1.4 extra-bytes descriptor (192 bytes): its data type and options bytes, and
# where its no_data/min/max triples of 8-byte "anytype" values start
_EB_SIZE, _EB_TYPE, _EB_OPTIONS, _EB_NAME, _EB_MIN, _EB_MAX = 192, 2, 3, 4, 64, 88
_OPT_MIN, _OPT_MAX = 0b0010, 0b0100
_SIGNED_TYPES = (2, 4, 6, 8)  # char, short, long, long long: an anytype int64


def write_extra_bytes_ranges(path: Path, ranges: dict[str, tuple[int, int]]) -> None:
    """Put each integer extra dimension's (min, max) of ``ranges`` into the extra-bytes
    VLR of the LAS/LAZ file ``path``, in place, with the options bits saying they hold;
    a dimension not in ``ranges`` (no points) gets those bits cleared."""
    with open(path, "r+b") as f:
        head = f.read(375)
        header_size = struct.unpack_from("<H", head, 94)[0]
        n_vlrs = struct.unpack_from("<I", head, 100)[0]
        at = header_size
        for _ in range(n_vlrs):
            f.seek(at)
            vlr = f.read(54)
            user_id = vlr[2:18].rstrip(b"\0")
            record_id, length = struct.unpack_from("<HH", vlr, 18)
            if user_id == b"LASF_Spec" and record_id == 4:
                for k in range(length // _EB_SIZE):
                    base = at + 54 + k * _EB_SIZE
                    f.seek(base)
                    eb = bytearray(f.read(_EB_SIZE))
                    name = bytes(eb[_EB_NAME : _EB_NAME + 32]).rstrip(b"\0").decode()
                    span = ranges.get(name)
                    if span is None:
                        eb[_EB_OPTIONS] &= ~(_OPT_MIN | _OPT_MAX) & 0xFF
                    else:
                        eb[_EB_OPTIONS] |= _OPT_MIN | _OPT_MAX
                        anytype = "<q" if eb[_EB_TYPE] in _SIGNED_TYPES else "<Q"
                        struct.pack_into(anytype, eb, _EB_MIN, span[0])
                        struct.pack_into(anytype, eb, _EB_MAX, span[1])
                    f.seek(base)
                    f.write(eb)
                return
            at += 54 + length
