"""Coloured clouds as LAS 1.4 (laspy), for CloudCompare, PDAL and QGIS.

Point format 7 (x, y, z, intensity, GPS time, RGB) with Adjusted Standard GPS time (GPS
seconds minus 1e9, the global-encoding bit set), scale 1 mm and an offset at the
cloud's rounded minimum so coordinates keep millimetres, and the coordinate reference
system from ``crs`` (anything ``pyproj.CRS.from_user_input`` takes, e.g. "EPSG:25832")
as an OGC WKT VLR. Extra bytes: ``scan_index`` (uint32, the scan in the log) and
``coloured`` (uint8 0/1); ``user_data`` also holds the coloured flag for readers that
ignore extra bytes. RGB is 16-bit (8-bit values times 257), intensity clipped to
0..65535.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from acq.time.gpstime import gps_adjusted_standard_time

__all__ = ["LasStream"]


class LasStream:
    """A LAS 1.4 file (module docstring) written part by part to ``path``.tmp, renamed
    on :meth:`close` (:meth:`abort` removes it). The offset is the first part's rounded
    minimum; the header's extent, counts and GPS time span grow with every part."""

    def __init__(
        self, path: str | os.PathLike[str], *, crs: str | None = None, comments: Sequence[str] = ()
    ) -> None:
        import laspy
        import pyproj

        self.path = Path(path)
        self._tmp = self.path.with_name(self.path.name + ".tmp")
        header = laspy.LasHeader(point_format=7, version="1.4")
        header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
        header.scales = np.array([0.001, 0.001, 0.001])
        header.generating_software = "acq colorize"
        if comments:
            header.system_identifier = str(comments[0])[:32]
        if crs:
            header.add_crs(pyproj.CRS.from_user_input(crs))
        header.add_extra_dims(
            [
                laspy.ExtraBytesParams(name="scan_index", type=np.uint32),
                laspy.ExtraBytesParams(name="coloured", type=np.uint8),
            ]
        )
        self._header = header
        self._writer: laspy.LasWriter | None = None

    def write(
        self, xyz: np.ndarray, rgb: np.ndarray, utc_s: np.ndarray, intensity: np.ndarray,
        scan: np.ndarray, coloured: np.ndarray,
    ) -> None:  # fmt: skip
        """Append points: ``xyz`` (N,3) m, ``rgb`` (N,3) uint8, ``utc_s`` (N,) UTC
        seconds, ``intensity``, ``scan`` index, ``coloured`` flag."""
        import laspy

        n = xyz.shape[0]
        if n == 0:
            return
        if self._writer is None:
            # column by column: numpy's axis-0 reduction of an (N,3) array is 9x slower
            self._header.offsets = np.floor([xyz[:, k].min() for k in range(3)])
            self._writer = laspy.open(self._tmp, mode="w", header=self._header, do_compress=False)
        header = self._writer.header
        # the raw record array filled column by column (laspy's scaled setters copy and
        # check each one: three times slower on millions of points)
        record = laspy.PackedPointRecord.zeros(n, header.point_format)
        a = record.array
        for axis, name in enumerate("XYZ"):
            a[name] = np.rint((xyz[:, axis] - header.offsets[axis]) / header.scales[axis])
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
        self._writer.write_points(record)

    def close(self) -> int:
        """Finish the file; its size, bytes."""
        import laspy

        if self._writer is None:  # no points: a valid empty file
            self._writer = laspy.open(self._tmp, mode="w", header=self._header, do_compress=False)
        self._writer.close()
        self._tmp.replace(self.path)
        return self.path.stat().st_size

    def abort(self) -> None:
        """Drop the unfinished file."""
        if self._writer is not None:
            self._writer.close()
        self._tmp.unlink(missing_ok=True)
