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

from acq.gpstime import gps_adjusted_standard_time

__all__ = ["write_las"]


def write_las(
    path: str | os.PathLike[str],
    xyz: np.ndarray,
    rgb: np.ndarray,
    utc_s: np.ndarray,
    intensity: np.ndarray,
    scan: np.ndarray,
    coloured: np.ndarray,
    *,
    crs: str | None = None,
    comments: Sequence[str] = (),
) -> int:
    """Write the points (``xyz`` (N,3) m, ``rgb`` (N,3) uint8, ``utc_s`` (N,) UTC
    seconds, ``intensity``, ``scan`` index, ``coloured`` flag) as LAS 1.4; returns the
    file's size, bytes. Written to a temporary name, then renamed."""
    import laspy
    import pyproj

    n = xyz.shape[0]
    # column by column: numpy's axis-0 reduction of an (N,3) array is 9x slower
    lo = np.array([xyz[:, k].min() for k in range(3)]) if n else np.zeros(3)
    hi = np.array([xyz[:, k].max() for k in range(3)]) if n else np.zeros(3)
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(lo)
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
    las = laspy.LasData(header, points=record)
    # the header's extent and counts from the data we have (laspy's update_header
    # reduces every column again and sorts the returns)
    header.point_count = n
    header.number_of_points_by_return = np.array([n] + [0] * 14)
    if n:
        header.mins, header.maxs = lo, hi
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    las.write(str(tmp), do_compress=False)
    tmp.replace(path)
    return path.stat().st_size
